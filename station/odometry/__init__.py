"""Stereo visual odometry (the paper's section 3.3): features, the paper's method, a robust variant."""

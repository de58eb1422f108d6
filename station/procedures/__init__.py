"""Alignment procedures of several captures around the cycle: runout compensation by rolling
the car, the steering sweep for caster and SAI."""

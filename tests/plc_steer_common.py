"""What the steering sweep's PLC tests share: the handshake's states and commands as numbers,
the sweep's steers, and the steering registers as they read when no sweep is on."""

IDLE, BUSY, DONE, FAULT, ROLL, STEER = 0, 1, 2, 3, 4, 5
MEASURE, ACK, COMPENSATED, IN_POSITION, CASTER = 1, 4, 5, 6, 7
FRONT = ("FL", "FR")
PLAN_DEG = [10.0, -10.0, 0.0]  # station/procedures/steering.py: STEER_PLAN (0, 1, -1, 0) x 10 deg, after the first
CLEARED_STEER = {"steer_step": 0, "steer_steps": 0, "steer_target_i16": 0.0, "FL_steer_i16": None,
                 "FR_steer_i16": None, "steer_reached": 0, "steer_readings": 0}

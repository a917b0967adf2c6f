"""The simulated spacecraft process: truth simulation on the planner's MuJoCo model, joint
servos, attitude control, the onboard time-based schedule and the emulated relay link.

It meets the ground server only on the wire.
"""

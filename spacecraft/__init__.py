"""The simulated spacecraft process: truth simulation on the planner's MuJoCo model, joint
servos, attitude control, the onboard command buffer and the emulated relay link.

Built by the spacecraft issue; it meets the ground server only on the wire.
"""

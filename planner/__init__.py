"""Flight dynamics and planning for free-flying robots (ETS-VII by default).

numpy, scipy and MuJoCo only: no clock, no logging setup. Time, randomness and parameters
come in as arguments. The one place that reads files is ``description`` (a robot description:
TOML plus URDF, read whole and validated before anything uses it); everything else is pure.

Modules: ``model`` (the canonical description), ``description`` (robots from files),
``frames`` and ``state`` (conventions), ``mujoco_conventions`` (the one place that speaks
MuJoCo's), ``mjcf`` and ``urdf`` (exports), ``dynamics`` (quantities of SPEC section 2),
``gravity_gradient``, ``ik``, ``ptp``, ``free_drift`` (eq. 9-10 prediction) and
``simulation`` (the free-floating core); the planners ``experiments`` (PTP, reactionless),
``reactionless``, ``gjm``, ``coordination``, ``nonholonomic``, ``servo_compensation`` and
``schedule``, on the shared ``plan``, ``prediction``, ``attitude_control`` and
``closed_loop``.
"""

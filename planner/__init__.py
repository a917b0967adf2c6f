"""Flight dynamics and planning for free-flying robots (ETS-VII by default).

numpy, scipy and MuJoCo only: no clock, no logging setup. Time, randomness and parameters
come in as arguments. The one place that reads files is the ``description`` package, the
planner's edge (a robot description: TOML plus URDF, read whole, parsed, checked, then built
into a ``robot.RobotDescription``; an ``[acs]`` file). Everything else is the pure core: it
imports neither ``description`` nor ``tomllib``, and its modules form no import circle (both
are import contracts in pyproject.toml).

Modules: ``model`` (the canonical description), ``robot`` (a loaded description),
``description`` (robots from files), ``frames`` and ``state`` (conventions),
``mujoco_conventions`` (the one place that speaks MuJoCo's), ``mjcf`` and ``urdf`` (exports),
``dynamics`` (quantities of SPEC section 2), ``gravity_gradient``, ``ik``, ``ptp``,
``free_drift`` (eq. 9-10 prediction) and ``simulation`` (the free-floating core); the
planners ``experiments`` (PTP, reactionless), ``reactionless`` (and ``reactionless_search``),
``gjm``, ``coordination``, ``nonholonomic`` (its paths in ``nonholonomic_paths``),
``servo_compensation`` and ``schedule``, on the shared ``plan``, ``prediction``,
``attitude_control`` (run by ``attitude_law``) and ``closed_loop``; ``parameters``
(experiment parameters from text or JSON) and ``catalogue`` (the experiments by name).
"""

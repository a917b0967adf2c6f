"""The operations layer: what an operator asks of the ground, once, for every caller.

Below the command line (:mod:`hikoboshi`) and the routes (:mod:`server.api`), above the
services, the planner, the mission and storage. A rule of operations is written here once and
used by the CLI, the routes, the demo and the campaign demo alike:

- checked planning: plan an experiment, check it against its robot's flight rules and fit it
  to a window, in one call;
- the window-fit rule (one error code) and the start lead (one formula, for scheduling, the
  start gate and the runner alike);
- the campaign: a series of passes planned into a mission's contact windows.

The live path's services (the runner, the uplink) sit below it: what they need of a rule
here is handed to them by the composition root (:mod:`server.app`).
"""

"""Whole passes on the simulated link (tests/server/link/simulated.py)."""

from __future__ import annotations

from pathlib import Path

from server.services.clock import ManualClock
from tests.server.link.simulated import SimulatedSpacecraft, ground, make_sessions, store_pass


async def run_pass(
    tmp_path: Path,
    n_commands: int,
    *,
    seconds: float,
    abort_at_s: float | None = None,
    stall: tuple[float, float] | None = None,
    drop: tuple[float, float] | None = None,
    settings: dict[str, float] | None = None,
    **spacecraft_kw: object,
) -> tuple[SimulatedSpacecraft, object, str]:
    """A pass of ``n_commands`` started on a simulated ground and flown ``seconds`` (an
    abort, a ground stall or a link drop at the onboard seconds given): the spacecraft, the
    ground, the pass."""
    clock = ManualClock()
    sessions = make_sessions(tmp_path)
    g = ground(sessions, clock, **(settings or {}))
    sc = SimulatedSpacecraft(clock, **spacecraft_kw)  # type: ignore[arg-type]
    await sc.connect(g)
    pass_id = store_pass(sessions, n_commands, clock)
    await g.runner.start(pass_id, "otto")
    t = 0.0
    step = 1.0
    while t < seconds:
        if abort_at_s is not None and t <= abort_at_s < t + step:
            await sc.run(abort_at_s - t)
            await g.runner.abort(pass_id, "otto", "operator abort")
            t = abort_at_s
            abort_at_s = None
            continue
        if stall is not None and t <= stall[0] < t + step:
            await sc.run(stall[0] - t)
            await sc.stall_ground(stall[1])
            t = stall[0] + stall[1]
            stall = None
            continue
        if drop is not None and t <= drop[0] < t + step:
            await sc.run(drop[0] - t)
            await sc.disconnect()
            await sc.run(drop[1])
            await sc.connect(g)
            t = drop[0] + drop[1]
            drop = None
            continue
        await sc.run(step)
        t += step
    await g.db.drain()
    return sc, g, pass_id

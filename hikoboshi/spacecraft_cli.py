"""``hikoboshi spacecraft``: the simulated spacecraft as its own process, the vehicle behind
an emulated relay link to the ground service (:mod:`spacecraft.process`), from its options:
the link's, the vehicle's (robot, attitude control, servos, sensor noise, faults, safing),
a mission's contact windows, and its token."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Annotated, Any

import typer

from hikoboshi.cli_common import (
    LogFormatOption,
    LogLevelOption,
    RobotOption,
    _configure_logging,
    _fail,
    _load,
)

__all__ = ["register"]


def spacecraft(
    ground: Annotated[
        list[str],
        typer.Option(
            help="Ground link endpoint, ws://HOST:PORT/PATH; repeat it for a hot standby's "
            "(tried in order after a drop or a standby's refusal)"
        ),
    ],
    token: Annotated[
        str | None,
        typer.Option(
            envvar="HIKOBOSHI_SPACECRAFT_TOKEN",
            show_envvar=True,
            help="API token with the spacecraft role (better from the environment or "
            "--token-file: a command line is visible to every user of the host)",
        ),
    ] = None,
    token_file: Annotated[
        Path | None,
        typer.Option(
            envvar="HIKOBOSHI_SPACECRAFT_TOKEN_FILE",
            show_envvar=True,
            help="A file holding the token (a container secret)",
        ),
    ] = None,
    time_scale: Annotated[float, typer.Option(help="Onboard seconds per wall second")] = 1.0,
    delay: Annotated[float | None, typer.Option(help="One-way delay, s (both directions)")] = None,
    jitter: Annotated[float | None, typer.Option(help="Delay jitter, s (1 sigma)")] = None,
    loss: Annotated[float | None, typer.Option(help="Message loss probability [0, 1)")] = None,
    outage: Annotated[
        list[str] | None, typer.Option(help="LOS window START:END in onboard s; repeatable")
    ] = None,
    bandwidth: Annotated[float | None, typer.Option(help="Link bandwidth cap, bytes/s")] = None,
    link_config: Annotated[
        Path | None, typer.Option(help="TOML file with [link], [uplink], [downlink] tables")
    ] = None,
    garbage: Annotated[
        list[str] | None,
        typer.Option(
            # "\\:" for Markdown's ":": rich read ":END:" as an emoji code
            help="Noise toward the ground START:END\\:RATE: malformed messages (invalid JSON, "
            "unknown types, wrong versions, malformed telemetry, in turn) at RATE per wall "
            "second while the onboard clock is in [START, END) s (as --outage); repeatable "
            "(docs/protocol.md, Malformed messages)"
        ),
    ] = None,
    telemetry_rate_hz: Annotated[float, typer.Option(help="Telemetry frames per second")] = 10.0,
    seed: Annotated[int, typer.Option(help="Seed for link and sensor noise")] = 0,
    los_policy: Annotated[
        str,
        typer.Option(
            help="Silence from the ground: 'continue' the loaded schedule, or 'hold' the arm "
            "(refuse queued joint commands) after --los-hold-after seconds"
        ),
    ] = "continue",
    los_hold_after: Annotated[
        float | None, typer.Option(help="Onboard seconds of silence before 'hold' holds the arm")
    ] = None,
    acs_config: Annotated[
        Path | None,
        typer.Option(
            help="TOML file with an acs table: the attitude-control law (bandwidth_radps, "
            "damping_ratio, integral_time_s, rate_filter_tau_s, dead_band_deg, "
            "torque_limit_nm, ...; docs/spacecraft.md); default the calibrated PD law (with "
            "--robot: the description's, whose keys the file's replace)"
        ),
    ] = None,
    robot: RobotOption = None,
    vehicle_config: Annotated[
        Path | None,
        typer.Option(
            help="TOML file with a servo and/or a sensor_noise table (a robot description's "
            "keys; hikoboshi calibrate --vehicle-out writes one): the joint servos and sensor "
            "noise flown, replacing the defaults (with --robot: the description's)"
        ),
    ] = None,
    fault: Annotated[
        list[str] | None,
        typer.Option(
            help="A fault injected in the truth simulation, NAME@T[,key=value...], T in onboard "
            "s from the start, or NAME@cmd+T, T after the first command executed: "
            "jointN-stuck@T, jointN-drift@T[,rate_degps=0.5], wheelN-fail@T, "
            "attitude-bias@T[,deg=3.0][,axis=x], bump@T[,nms=10][,axis=x]; repeatable "
            "(docs/spacecraft.md)"
        ),
    ] = None,
    truth_log: Annotated[
        Path | None,
        typer.Option(
            help="Write the truth log here (JSON lines: each fault's onset, each entry into "
            "and exit from on-board safing; never sent to the ground)"
        ),
    ] = None,
    no_safing: Annotated[
        bool,
        typer.Option(
            "--no-safing",
            help="Fly without on-board safing (rehearse the ground's alarms with no on-board "
            "protection)",
        ),
    ] = False,
    mission: Annotated[
        Path | None,
        typer.Option(
            help="A mission file (docs/missions.md): the link is up only inside its contact "
            "windows and its one-way delay is the ground's processing delay plus the path's "
            "light time (replacing --delay); the gaps are flown fast"
        ),
    ] = None,
    mission_start: Annotated[
        str | None,
        typer.Option(
            help="With --mission: the UTC (ISO 8601) of the spacecraft's onboard second 0, "
            "which its onboard clock reads (default: the mission's elements' epoch)"
        ),
    ] = None,
    windows: Annotated[
        Path | None,
        typer.Option(
            help="With --mission: fly these windows (hikoboshi windows --json, or a "
            "campaign.json) instead of every window of --hours from the start"
        ),
    ] = None,
    relay: Annotated[
        list[str] | None,
        typer.Option(help="With --mission: only this relay's windows; repeatable"),
    ] = None,
    hours: Annotated[
        float, typer.Option(help="With --mission and no --windows: hours of windows")
    ] = 24.0,
    fast_scale: Annotated[
        float | None,
        typer.Option(
            help="With --mission: between windows the onboard clock runs at most this many "
            "times wall time (default: as fast as the simulation computes)"
        ),
    ] = None,
    log_format: LogFormatOption = "text",
    log_level: LogLevelOption = "info",
) -> None:
    """Run the simulated spacecraft: the vehicle behind an emulated TDRS relay link. With
    --robot it flies that robot description (model, servos, attitude control, wheel limits,
    sensor noise, live limits) and names it, with its hash and joint count, in hello. The
    vehicle safes itself on a red limit unless --no-safing; --fault injects faults."""
    import asyncio
    import dataclasses
    import logging
    import signal

    from server.redaction import install_redaction
    from spacecraft.faults import parse_fault
    from spacecraft.link import LinkConfig, load_link_config, parse_garbage, parse_outage
    from spacecraft.process import ProcessConfig, SpacecraftProcess
    from spacecraft.vehicle_config import VehicleConfig, vehicle_config_for

    install_redaction()  # its token never in its log (docs/security.md "Logs")
    _configure_logging(log_format, log_level)
    token = _spacecraft_token(token, token_file)
    try:
        if link_config is not None:
            up, down = load_link_config(link_config)
        else:
            up, down = LinkConfig(seed=seed), LinkConfig(seed=seed + 1)
        changes: dict[str, Any] = {}
        if delay is not None:
            changes["delay_s"] = delay
        if jitter is not None:
            changes["jitter_s"] = jitter
        if loss is not None:
            changes["loss"] = loss
        if bandwidth is not None:
            changes["bandwidth_bps"] = bandwidth
        if outage:
            changes["outages"] = tuple(parse_outage(o) for o in outage)
        up = dataclasses.replace(up, **changes)
        down = dataclasses.replace(down, **changes)
        vehicle_fields: dict[str, Any] = {
            "telemetry_period_s": 1.0 / telemetry_rate_hz,
            "los_policy": los_policy,  # VehicleConfig checks it
            "los_hold_after_s": los_hold_after,
            "faults": tuple(parse_fault(f) for f in fault or ()),
            "safing": not no_safing,
        }
        if truth_log is not None and not truth_log.parent.is_dir():
            raise ValueError(f"--truth-log {truth_log}: no directory {truth_log.parent}")
        if robot is not None:
            vehicle = vehicle_config_for(
                _load(robot),
                acs_overrides=None if acs_config is None else _acs_table(acs_config),
                **vehicle_fields,
            )
        else:
            if acs_config is not None:
                from planner.description import load_acs_config
                from planner.dynamics import DynamicsWorkspace
                from planner.model import default_model

                vehicle_fields["acs_gains"] = load_acs_config(
                    DynamicsWorkspace(default_model()), acs_config
                )
            vehicle = VehicleConfig(**vehicle_fields)
        if vehicle_config is not None:
            vehicle = _with_vehicle_tables(vehicle, vehicle_config)
        contact = epoch_ns = None
        if mission is not None:
            contact, epoch_ns = _contact(mission, mission_start, windows, relay or (), hours)
        elif any(o is not None for o in (mission_start, windows, relay, fast_scale)):
            raise ValueError("--mission-start, --windows, --relay and --fast-scale need --mission")
        config = ProcessConfig(
            ground_url=ground[0],
            standby_urls=tuple(ground[1:]),
            token=token,
            time_scale=time_scale,
            vehicle=vehicle,
            uplink=up,
            downlink=down,
            seed=seed,
            truth_log=truth_log,
            garbage=tuple(parse_garbage(g) for g in garbage or ()),
            contact=contact,
            fast_scale=fast_scale,
            epoch_ns=epoch_ns,
        )
    except (ValueError, OSError) as exc:
        _fail(str(exc))

    async def main_async() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        process = SpacecraftProcess(config)
        await process.run(stop)
        # a log record, in --log-format as every other line of the process (a plain line
        # broke a JSON log)
        logging.getLogger("hikoboshi.spacecraft").info(
            "spacecraft stopped: %d frames unacknowledged, %d connections%s",
            process.store.unacked,
            process.connections,
            f", {process.garbage_sent} malformed messages sent" if garbage else "",
            extra={
                "fields": {
                    "event": "spacecraft_stopped",
                    "frames_unacknowledged": process.store.unacked,
                    "connections": process.connections,
                }
            },
        )

    asyncio.run(main_async())


def _contact(
    mission: Path, start: str | None, windows: Path | None, relays: Sequence[str], hours: float
) -> tuple[Any, int]:
    """The spacecraft's contact plan from its --mission options (ValueError: one line), and
    its onboard clock at its start: the mission's start in UTC ns, so that the onboard clock
    reads the mission's time (the ground judges the windows on it with
    ``window_clock = "vehicle"``, docs/missions.md)."""
    from mission import MissionError, load_mission, parse_utc
    from spacecraft.contact import load_contact

    try:
        start_utc = load_mission(mission).orbit.epoch_utc if start is None else parse_utc(start)
    except MissionError as exc:
        raise ValueError(str(exc)) from None
    contact = load_contact(mission, start_utc, windows_path=windows, relays=relays, hours=hours)
    since_1970 = start_utc - datetime(1970, 1, 1, tzinfo=UTC)
    return contact, since_1970 // timedelta(microseconds=1) * 1000


def _spacecraft_token(token: str | None, token_file: Path | None) -> str:
    """The spacecraft's token: given, else read from ``token_file``; one error line when
    there is none (docs/operations.md "Settings")."""
    if token and token.strip():
        return token.strip()
    if token_file is not None:
        try:
            text = token_file.read_text().strip()
        except OSError as exc:
            _fail(f"--token-file {token_file}: {exc.strerror or exc}")
        if not text:
            _fail(f"--token-file {token_file} is empty")
        return text
    _fail(
        "no spacecraft token: give --token-file FILE or set HIKOBOSHI_SPACECRAFT_TOKEN "
        "(or HIKOBOSHI_SPACECRAFT_TOKEN_FILE)"
    )


def _with_vehicle_tables(vehicle: Any, path: Path) -> Any:
    """``vehicle`` (a VehicleConfig) with the servos and sensor noise of ``path``'s
    ``[servo]`` and ``[sensor_noise]`` tables (planner.description.load_vehicle_tables)."""
    import dataclasses

    from planner.description import load_vehicle_tables, servo_gains_of
    from spacecraft.vehicle_config import SensorNoise

    tables = load_vehicle_tables(path, vehicle.model.n_joints)
    if tables.servo is not None:
        sim = dataclasses.replace(vehicle.sim, servo=servo_gains_of(tables.servo, vehicle.model))
        vehicle = dataclasses.replace(vehicle, sim=sim)
    if tables.sensor_noise is not None:
        noise = SensorNoise(**dataclasses.asdict(tables.sensor_noise))
        vehicle = dataclasses.replace(vehicle, noise=noise)
    return vehicle


def _acs_table(path: Path) -> dict[str, object]:
    """The ``[acs]`` table of an attitude-control TOML file (``--acs-config``)."""
    import tomllib

    try:
        with path.open("rb") as f:
            doc = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the attitude-control configuration: {exc}") from None
    if set(doc) != {"acs"} or not isinstance(doc["acs"], dict):
        raise ValueError(f"{path}: expected one [acs] table (found {sorted(doc)})")
    return dict(doc["acs"])


def register(app: typer.Typer) -> None:
    """Add ``spacecraft`` to ``hikoboshi``."""
    app.command("spacecraft")(spacecraft)

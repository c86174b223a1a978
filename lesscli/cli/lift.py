"""``less lift``: drive the scissor lift that re-orients inserts, or emulate its servos on a pty.

Every command opens the bus, checks the servos, acts, and drops torque on the way out (also on errors and
Ctrl-C). Telemetry records (time, height in mm, rotation in deg, orientation, moving, torque, errors) go to
stdout as JSON lines. ``dynamixel_sdk`` is imported only inside the command bodies.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, replace

import click

from lesscli.cli.common import Group, checked_output, format_option, orientations_option
from lesscli.errors import LessError


@dataclass
class _Options:
    port: str | None
    baud: int | None
    config_path: str | None
    ids: tuple[int, int] | None
    fmt: str | None

    def config(self):
        from lesscli.hardware.config import load_config

        lift_id, rotator_id = self.ids or (None, None)
        return load_config(self.config_path, baud=self.baud, lift_id=lift_id, rotator_id=rotator_id)


class _Sink:
    """Telemetry to stdout: streamed JSON lines, or collected for json/table/markdown."""

    def __init__(self, fmt: str | None) -> None:
        from lesscli.io.records import resolve_format

        self.fmt = resolve_format(fmt, sys.stdout)
        self.rows: list[dict] = []

    def __call__(self, record: dict) -> None:
        if self.fmt == "jsonl":
            from lesscli.io.records import dumps

            sys.stdout.write(dumps(record) + "\n")
            sys.stdout.flush()
        else:
            self.rows.append(record)

    def close(self) -> None:
        if self.rows:
            from lesscli.io.records import emit_records

            emit_records(self.rows, self.fmt)
            self.rows = []


def _parse_ids(ctx, param, value: str | None) -> tuple[int, int] | None:
    if value is None:
        return None
    try:
        lift_id, rotator_id = (int(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"'{value}': expected LIFT,ROTATOR servo ids, e.g. 1,2") from None
    if not (0 <= lift_id <= 252 and 0 <= rotator_id <= 252):
        raise click.BadParameter(f"'{value}': servo ids are 0..252")
    return lift_id, rotator_id


PORT_HELP = "Serial port of the servo bus (env LESS_LIFT_PORT)."
BAUD_HELP = "Baud rate (default from lift.toml, else 57600)."
CONFIG_HELP = "lift.toml (limits, geometry, ids)."
IDS_HELP = "LIFT,ROTATOR servo ids (default 1,2)."


@click.group(cls=Group)
@click.option("--port", envvar="LESS_LIFT_PORT", help=PORT_HELP)
@click.option("--baud", type=int, default=None, help=BAUD_HELP)
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help=CONFIG_HELP)
@click.option("--ids", callback=_parse_ids, help=IDS_HELP)
@format_option()
@click.pass_context
def cli(ctx, port, baud, config_path, ids, fmt) -> None:
    """Scissor lift: home, raise, lower, rotate the insert, cycle through orientations; or emulate it.

    Try it without hardware: 'less lift emulate --link /tmp/lift &' then 'less lift --port /tmp/lift home'.
    """
    ctx.obj = _Options(port, baud, config_path, ids, fmt)


def _pass_options(func):
    """``click.pass_obj`` for the commands that drive the bus; they also take the group's options after
    their name (``less lift status --port /dev/ttyUSB0 --format table``), which override the group's."""
    @functools.wraps(func)
    def run(*args, fmt: str | None = None, sub_port: str | None = None, sub_baud: int | None = None,
            sub_config: str | None = None, sub_ids: tuple[int, int] | None = None, **kwargs):
        opts = click.get_current_context().find_object(_Options)
        given = {"fmt": fmt, "port": sub_port, "baud": sub_baud, "config_path": sub_config, "ids": sub_ids}
        return func(replace(opts, **{k: v for k, v in given.items() if v is not None}), *args, **kwargs)
    run = click.option("--ids", "sub_ids", callback=_parse_ids, help=IDS_HELP)(run)
    run = click.option("--config", "sub_config", type=click.Path(dir_okay=False), help=CONFIG_HELP)(run)
    run = click.option("--baud", "sub_baud", type=int, default=None, help=BAUD_HELP)(run)
    run = click.option("--port", "sub_port", default=None, help=PORT_HELP)(run)
    return format_option()(run)


def _terminated(signum, frame) -> None:
    raise SystemExit(128 + signal.SIGTERM)


def _session(opts: _Options, action) -> None:
    """Open the bus and the lift, run ``action(lift, emit)``, always drop torque and flush telemetry."""
    from lesscli.hardware.bus import DynamixelBus
    from lesscli.hardware.lift import ScissorLift

    config = opts.config()
    port = opts.port or config.port
    if not port:
        raise click.UsageError("no port: give --port PATH, set LESS_LIFT_PORT or [bus] port in lift.toml")
    sink = _Sink(opts.fmt)
    previous = signal.signal(signal.SIGTERM, _terminated)  # unwind (torque off) when killed, like Ctrl-C
    try:
        with (DynamixelBus(port, config.baud, config.retries, config.latency_ms) as bus,
              ScissorLift(bus, config, emit=sink) as lift):
            action(lift, sink)
    finally:
        signal.signal(signal.SIGTERM, previous)
        sink.close()


@cli.command()
@_pass_options
def status(opts: _Options) -> None:
    """One telemetry record: homed, height, rotation, orientation, torque, hardware errors."""
    _session(opts, lambda lift, emit: emit(lift.status()))


@cli.command()
@_pass_options
def home(opts: _Options) -> None:
    """Reboot faulted servos, find the lower stop, zero the screw count, then lower."""
    _session(opts, lambda lift, emit: (lift.home(), emit(lift.status("done"))))


@cli.command("raise")
@_pass_options
def raise_cmd(opts: _Options) -> None:
    """Raise the insert into its shell (raised_height_mm)."""
    _session(opts, lambda lift, emit: (lift.raise_(), emit(lift.status("done"))))


@cli.command()
@_pass_options
def lower(opts: _Options) -> None:
    """Lower the insert out of its shell (lowered_height_mm)."""
    _session(opts, lambda lift, emit: (lift.lower(), emit(lift.status("done"))))


@cli.command()
@click.option("--height-mm", type=float, required=True, help="Platform height, within the configured limits.")
@_pass_options
def move(opts: _Options, height_mm: float) -> None:
    """Move the platform to a height in mm."""
    _session(opts, lambda lift, emit: (lift.move_to_height(height_mm), emit(lift.status("done"))))


@cli.command()
@click.argument("orientation", type=click.IntRange(0, 7))
@_pass_options
def rotate(opts: _Options, orientation: int) -> None:
    """Turn the insert to ORIENTATION (0..7, 45 degrees each); the lift must be lowered."""
    _session(opts, lambda lift, emit: (lift.rotate(orientation), emit(lift.status("done"))))


def _exec_runner(template: str):
    def run(k: int) -> None:
        argv = shlex.split(template.replace("{orientation}", str(k)))
        env = {**os.environ, "LESS_LIFT_ORIENTATION": str(k)}
        try:
            proc = subprocess.run(argv, check=False, stdout=subprocess.PIPE, env=env)
        except OSError as exc:
            raise LessError(f"cycle stopped at orientation {k}: cannot run '{argv[0]}': "
                            f"{exc.strerror}") from None
        if proc.stdout:
            click.echo(proc.stdout.decode(errors="replace"), err=True, nl=False)
        if proc.returncode != 0:
            raise LessError(f"cycle stopped at orientation {k}: --exec command exited with "
                            f"{proc.returncode}: {shlex.join(argv)}")

    return run


@cli.command()
@orientations_option(help="Orientations to visit in order, e.g. 0-7 or 0,2,4.")
@click.option("--exec", "exec_", default=None,
              help="Command run at each orientation once raised; '{orientation}' is replaced (its stdout "
                   "goes to stderr). A failure stops the cycle.")
@_pass_options
def cycle(opts: _Options, orientations: list[int], exec_: str | None) -> None:
    """For each orientation: lower, rotate, raise, then run --exec."""
    run = _exec_runner(exec_) if exec_ else None
    _session(opts, lambda lift, emit: (lift.cycle(orientations, run), emit(lift.status("done"))))


@cli.command("torque-off")
@_pass_options
def torque_off(opts: _Options) -> None:
    """Drop torque on both servos (works without homing)."""
    from lesscli.hardware.bus import DynamixelBus
    from lesscli.hardware.lift import ScissorLift

    config = opts.config()
    port = opts.port or config.port
    if not port:
        raise click.UsageError("no port: give --port PATH, set LESS_LIFT_PORT or [bus] port in lift.toml")
    sink = _Sink(opts.fmt)
    with DynamixelBus(port, config.baud, config.retries, config.latency_ms) as bus:
        failures = ScissorLift(bus, config).release()
        sink({"event": "torque-off", "port": port, "ids": [config.lift_id, config.rotator_id],
              "failures": failures})
    sink.close()
    if failures:
        raise LessError(failures[0])


@cli.command()
@click.option("--link", type=click.Path(), help="Also make this symlink to the pty (removed on exit).")
@click.option("--fault", "faults", multiple=True, metavar="NAME[:ID[:N[:COUNT]]]",
              help="Inject a fault (no-reply, bad-crc, overload, overheating, stall, power-cycle) on servo "
                   "ID (default: the lift) at its N-th Goal_Position write (default 1; 0 = at start); COUNT "
                   "limits no-reply/bad-crc to that many replies. Repeatable.")
@click.option("--time-scale", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              help="Simulated seconds per wall-clock second (e.g. 100 makes moves take milliseconds).")
@click.option("--log", "log_path", type=click.Path(dir_okay=False), callback=checked_output(),
              help="Write goal/fault events as JSON lines.")
@click.pass_obj
def emulate(opts: _Options, link: str | None, faults: tuple[str, ...], time_scale: float,
            log_path: str | None) -> None:
    """Emulate the lift's two servos on a pseudo-terminal; print its path and run until interrupted."""
    from lesscli.hardware.emulator import PtyEmulator, ServoEmulator, lift_servos, parse_fault

    config = opts.config()
    servos = lift_servos(config)
    armed = []
    for spec in faults:
        try:
            servo_id, fault = parse_fault(spec, config.lift_id)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--fault") from None
        if servo_id not in {s.servo_id for s in servos}:
            raise click.BadParameter(f"'{spec}': no servo {servo_id} on the emulated bus",
                                     param_hint="--fault")
        armed.append((servo_id, fault))
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    with contextlib.ExitStack() as stack:
        log = stack.enter_context(open(log_path, "a", encoding="utf-8")) if log_path else None
        emulator = ServoEmulator(servos, time_scale=time_scale, log=log)
        for servo_id, fault in armed:
            emulator.arm(servo_id, fault)
        pty = stack.enter_context(PtyEmulator(emulator, link=link))
        click.echo(pty.port)
        sys.stdout.flush()
        click.echo(f"less: emulating servos {config.lift_id} (lift) and {config.rotator_id} (rotator) on "
                   f"{pty.port}; Ctrl-C stops", err=True)
        while True:
            time.sleep(0.5)

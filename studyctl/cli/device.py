"""``studyctl device list|check``: the devices this installation can drive, and a device's health."""

from __future__ import annotations

import json
from pathlib import Path

import typer
import yaml

from studyctl.cli.common import DB_OPTION, STUDY_OPTION, WORKSPACE_OPTION, output_console, workspace_arg
from studyctl.errors import UsageError


def _params(pairs: list[str]) -> dict:
    """``KEY=VALUE`` pairs (VALUE read as YAML: numbers, lists) into device parameters."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise UsageError(f"--param {pair!r}: write KEY=VALUE, e.g. --param host=192.168.1.20")
        out[key] = yaml.safe_load(value)
    return out


def register(app: typer.Typer) -> None:
    device_app = typer.Typer(help="List, check and emulate haptic devices.", no_args_is_help=True)

    @device_app.command("list")
    def list_command(as_json: bool = typer.Option(False, "--json", help="Print one JSON array.")) -> None:
        """Every device plugin: hardware or simulated, whether it has an emulator (for --emulate and rehearsals)."""
        from studyctl.engine.device_check import list_devices  # noqa: PLC0415

        frame = list_devices().to_frame()
        if as_json:
            typer.echo(json.dumps(frame.to_dict(orient="records")))
            return
        from studyctl.report.terminal import frame_table  # noqa: PLC0415 - only when a table is printed

        output_console().print(frame_table("studyctl devices", frame))

    @device_app.command("check")
    def check_command(
        name: str = typer.Argument(..., help="Device plugin name (see `studyctl device list`)."),
        emulate: bool = typer.Option(False, "--emulate", help="Check the device's emulator instead of the hardware."),
        seconds: float = typer.Option(3.0, "--seconds", help="How long to run the device's loop."),
        rate: float = typer.Option(None, "--rate", help="Loop rate in Hz (default: the device's)."),
        param: list[str] = typer.Option(None, "--param", help="Device parameter KEY=VALUE (repeatable)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
    ) -> None:
        """Connect, report identity and limits, measure loop rate and jitter, and exercise the safety layer on the
        device (clamp, NaN, watchdog). Exits 1 when a safety check fails."""
        from studyctl.engine.device_check import check_device  # noqa: PLC0415

        result = check_device(name, _params(param), emulate=emulate, seconds=seconds, rate_hz=rate)
        if as_json:
            typer.echo(json.dumps(result.to_json(), default=str))
        else:
            console = output_console()
            console.print(f"device {result.device}{' (emulated)' if result.emulated else ''}: "
                          f"{', '.join(f'{k}={v}' for k, v in result.identity.items()) or 'no identity reported'}")
            console.print(f"limits: {result.limits}")
            console.print(f"loop: {result.ticks} ticks in {result.seconds:g} s at {result.rate_hz:g} Hz "
                          f"(achieved {result.achieved_hz:.1f} Hz), period jitter p99 "
                          f"{result.period_jitter_us_p99:.0f} us, lateness p99 {result.late_us_p99:.0f} us; "
                          f"servo process: {result.rt}")
            from studyctl.report.terminal import safety_table  # noqa: PLC0415 - only when a table is printed

            console.print(safety_table(result.safety))
            for f in result.faults:
                console.print(f"[red]device fault: {f}[/red]")
        if not result.ok:
            raise typer.Exit(1)

    register_calibrate(device_app)
    app.add_typer(device_app, name="device")


def register_calibrate(device_app: typer.Typer) -> None:
    @device_app.command("calibrate")
    def calibrate_command(
        name: str = typer.Argument(..., help="Device plugin name (see `studyctl device list`)."),
        emulate: bool = typer.Option(False, "--emulate", help="Calibrate the device's emulator (used by rehearsals)."),
        seconds: float = typer.Option(2.0, "--seconds", help="How long to measure (keep the device at rest)."),
        param: list[str] = typer.Option(None, "--param", help="Device parameter KEY=VALUE (repeatable)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
        db: str = DB_OPTION,
        workspace: Path = WORKSPACE_OPTION,
        study: str = STUDY_OPTION,
    ) -> None:
        """Zero or calibrate a device (force sensor at rest, handle at its reference point) and store it in the study
        database with a timestamp; later sessions on the device use it and record which one."""
        from studyctl.engine.device_check import calibrate_device  # noqa: PLC0415
        from studyctl.store.workspace import open_study  # noqa: PLC0415

        with open_study(db, workspace_arg(workspace), study) as opened:
            cal = calibrate_device(opened.store, opened.study, name, _params(param), emulate=emulate, seconds=seconds)
        if as_json:
            typer.echo(json.dumps(vars(cal), default=str))
        else:
            typer.echo(f"calibration {cal.id} of {cal.device}{' (emulated)' if cal.emulated else ''} at "
                       f"{cal.created_at}: {cal.params} ({cal.detail.get('what', '')}, "
                       f"{cal.detail.get('samples', '?')} samples)")

"""The work of ``thermal-comp cnc-emulator`` (:mod:`cnc_bridge.cnc_emulator.cli` parses the arguments):
serve the emulated CNC until Ctrl-C / SIGTERM, alone or fed by the running twin."""
from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import signal
import sys

from cnc_bridge.cnc_emulator.access import open_access_warning
from cnc_bridge.cnc_emulator.probe import artefact_probe
from cnc_bridge.cnc_emulator.server import CncEmulator, EmulatorConfig
from cnc_bridge.cnc_emulator.thread import CncEmulatorThread
from cnc_bridge.credentials import CredentialsError, load_credentials
from thermal_comp_common.runtime.production import PRODUCTION_ENV, production_mode


def run(args: argparse.Namespace, ros_args: list[str]) -> int:
    """Serve as the parsed arguments say; the exit code (0 stopped, 1 cannot listen, 2 bad
    credentials or configuration)."""
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        creds = load_credentials(args.credentials_file)
        extra = {} if args.offset_limit_mm is None else {"offset_limit_mm": args.offset_limit_mm}
        cfg = EmulatorConfig(host=args.host, port=args.port,
                             position_axes=tuple(filter(None, args.axes.split(","))),
                             compensation_axes=tuple(filter(None, args.compensation_axes.split(","))),
                             user=creds.user, password=creds.password, certificate=args.certificate,
                             private_key=creds.private_key, security=args.security,
                             client_trust=tuple(args.client_trust), **extra)
    except (CredentialsError, ValueError) as exc:
        print(f"cnc-emulator: {exc}", file=sys.stderr)
        return 2
    if production_mode() and open_access_warning(cfg.security, bool(cfg.client_trust)):
        print(f"cnc-emulator: refused: --security {cfg.security} without --client-trust in a production cell "
              f"({PRODUCTION_ENV}=1): use --security required with a client trust list", file=sys.stderr)
        return 2
    if not args.verbose:
        logging.getLogger("asyncua").setLevel(logging.ERROR)
    if cfg.password is not None and not cfg.certificate:
        print("cnc-emulator: warning: a password without --certificate travels unencrypted",
              file=sys.stderr)
    if args.twin:
        return _serve_twin(cfg, ros_args)
    errors = dict(args.true_errors)
    probe = artefact_probe(lambda: errors) if args.probe_artefact else None

    async def serve() -> None:
        emu = CncEmulator(cfg, probe_move=probe)
        await emu.start()
        # what start-up allocated (asyncua, the address space) stays out of the collector's
        # passes: a full collection over it would pause an answer on the offsets' path
        gc.freeze()
        print(f"CNC emulator listening on {cfg.endpoint}", flush=True)
        _warn_if_open(cfg)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            await stop.wait()
        finally:
            await emu.stop()

    try:
        asyncio.run(serve())
    except OSError as exc:
        print(f"cnc-emulator: cannot listen on {cfg.endpoint}: {exc}", file=sys.stderr)
        return 1
    return 0


def _serve_twin(cfg: EmulatorConfig, ros_args: list[str]) -> int:
    """Serve the CNC fed by the twin until Ctrl-C / SIGTERM (an rclpy node in this process)."""
    # rclpy: only with --twin
    from thermal_comp_common.runtime.node_runtime import run_node
    from cnc_bridge.cnc_twin_feed_node import CncTwinFeed
    latest: list[dict[str, float]] = [{}]     # replaced whole by the feed (atomic), read by ProbeMove
    emu = CncEmulatorThread(cfg, probe_move=artefact_probe(lambda: latest[0]))
    try:
        emu.start()
    except OSError as exc:
        print(f"cnc-emulator: cannot listen on {cfg.endpoint}: {exc}", file=sys.stderr)
        emu.close()
        return 1
    print(f"CNC emulator listening on {cfg.endpoint}", flush=True)
    _warn_if_open(cfg)

    def feed(context):
        return CncTwinFeed(context=context, emulator=emu,
                           on_true_errors=lambda errors: latest.__setitem__(0, errors))
    feed.__name__ = "cnc-emulator"
    try:
        return run_node(feed, ["cnc-emulator"] + ros_args)
    finally:
        emu.close()


def _warn_if_open(cfg: EmulatorConfig) -> None:
    """One line on stderr when anyone may connect (after the readiness line, which callers
    wait for on the first line of the output)."""
    line = open_access_warning(cfg.security, bool(cfg.client_trust))
    if line:
        print(line, file=sys.stderr, flush=True)

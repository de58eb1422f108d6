"""`station serve`: the station as a Modbus device for the shop PLC (docs/plc.md), and with
`--opcua` as an OPC UA server too (docs/shop.md)."""

from __future__ import annotations

import asyncio
import logging
import signal
import sys

from station.commands.arguments import seed
from station.config import load_config
from station.errors import ConfigError


def add_arguments(parser):
    parser.add_argument("--host", help="address to listen on (default: plc.host, 127.0.0.1)")
    parser.add_argument("--port", type=int, help="TCP port (default: plc.port, 5020)")
    parser.add_argument("--rtu", metavar="DEVICE", help="serve Modbus RTU on this serial device instead of TCP")
    parser.add_argument("--baudrate", type=int, help="RTU baud rate (default: plc.baudrate)")
    parser.add_argument("--parity", choices=("N", "E", "O"), help="RTU parity (default: plc.parity)")
    parser.add_argument("--device-id", type=int, help="Modbus device id (default: plc.device_id)")
    parser.add_argument("--dry-run", action="store_true",
                        help="no cameras: answer every trigger with a synthetic result computed from "
                             "the job id (for commissioning the PLC program)")
    parser.add_argument("--fail-every", type=int, default=10, metavar="N",
                        help="with --dry-run: jobs whose number is a multiple of N fail with fault "
                             "401, so the PLC's fault branch is exercised (0: never; default 10)")
    parser.add_argument("--delay-s", type=float, default=0.0, metavar="S",
                        help="with --dry-run: each synthetic cycle takes this long (a stand-in for the measurement)")
    parser.add_argument("--store", action="store_true",
                        help="with --dry-run: keep every synthetic result in the history too (history.url or "
                             "SQLite), as a measuring station does")
    parser.add_argument("--opcua", action="store_true",
                        help="also serve the same device over OPC UA (default opcua.host:opcua.port, 127.0.0.1:4840; "
                             "docs/shop.md)")
    parser.add_argument("--opcua-host", help="OPC UA address to listen on (default: opcua.host); beyond loopback "
                                             "opcua.users must name who may log in")
    parser.add_argument("--opcua-port", type=int, help="OPC UA TCP port (default: opcua.port, 4840)")
    parser.add_argument("--seed", type=seed, default=None,
                        help="simulated station only: this random vehicle stands on the lift for every "
                             "cycle (default: each cycle measures the vehicle of its cycle number)")
    parser.add_argument("--cycles", type=int, metavar="N",
                        help="stop after N cycles have been acknowledged (tests, demos)")
    parser.add_argument("--heartbeat-s", type=float, default=0.1, help="heartbeat period (s)")
    parser.add_argument("--cycle-timeout-s", type=float, default=300.0,
                        help="a cycle longer than this ends in fault 505 (the time the PLC takes to roll the "
                             "car for runout compensation, and the time the front wheels take to be steered in a "
                             "steering sweep, not counted)")
    parser.add_argument("--roll-timeout-s", type=float,
                        help="a roll of the car (runout compensation, command 5) that the PLC does not confirm "
                             "within this ends the cycle in fault 415 (default: plc.roll_timeout_s, 120)")
    parser.add_argument("--steer-timeout-s", type=float,
                        help="a steer target of a steering sweep (command 7) that the front wheels do not stand at "
                             "within this ends the cycle in fault 424 (default: plc.steer_timeout_s, 120)")
    parser.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))


def _transport(args, plc) -> tuple[str, dict]:
    rtu = args.rtu or (plc.serial_port if plc.transport == "rtu" and not (args.host or args.port) else None)
    if plc.transport == "rtu" and not rtu and not (args.host or args.port):
        raise ConfigError("plc.transport is rtu but plc.serial_port is null",
                          hint="set plc.serial_port in config/station.yaml or pass --rtu DEVICE")
    if rtu:
        return "rtu", {"port": rtu, "baudrate": args.baudrate or plc.baudrate, "parity": args.parity or plc.parity}
    port = plc.port if args.port is None else args.port
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port {port}: expected 0..65535")
    return "tcp", {"host": args.host or plc.host, "port": port}


async def _send_outbox(config) -> None:
    """Every history.retry_s: send the cycles the history server could not take (station/records/outbox.py)."""
    from station.errors import StorageError
    from station.records.history import send_outbox

    log = logging.getLogger("station.history")
    while True:
        await asyncio.sleep(config.history.retry_s)
        try:
            sent = await asyncio.get_running_loop().run_in_executor(None, send_outbox, config)
        except StorageError as e:
            log.warning("outbox not sent: %s", e)
            continue
        if sent:
            log.info("%d cycle(s) from the outbox sent to the history server", sent)


async def _serve(args, runner, transport, where, device_id, plc, config) -> int:
    from station.plc.device import PlcDevice
    from station.plc.server import PlcServer, wait_until

    roll_timeout_s = plc.roll_timeout_s if args.roll_timeout_s is None else args.roll_timeout_s
    steer_timeout_s = plc.steer_timeout_s if args.steer_timeout_s is None else args.steer_timeout_s
    device = PlcDevice(runner, device_id=device_id, heartbeat_s=args.heartbeat_s,
                       cycle_timeout_s=args.cycle_timeout_s, roll_timeout_s=roll_timeout_s,
                       steer_timeout_s=steer_timeout_s)
    server = PlcServer(device, allowed_clients=plc.allowed_clients, max_connections=plc.max_connections,
                       idle_timeout_s=plc.idle_timeout_s)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    if transport == "rtu":
        await server.start_rtu(**where)
    else:
        where["port"] = await server.start_tcp(**where)
        server.address = f"Modbus TCP {where['host']}:{where['port']}"
    opcua = None
    if args.opcua:
        from station.plc.opcua_server import OpcUaServer
        opcua = OpcUaServer(device, host=args.opcua_host or config.opcua.host,
                            port=config.opcua.port if args.opcua_port is None else args.opcua_port,
                            users=config.opcua.users, station_name=config.name)
        try:
            await opcua.start()
        except BaseException:
            await server.stop()
            raise
    background = []
    if config.history.url is not None:  # resend what the history server could not take, while idle too
        background.append(asyncio.create_task(_send_outbox(config)))
    mode = "dry run: synthetic results" if args.dry_run else "measuring"
    also = f" and OPC UA {opcua.endpoint}" if opcua else ""
    print(f"station serving {server.address}{also}, device id {device_id} ({mode}); Ctrl-C to stop", flush=True)
    try:
        if args.cycles:
            waiter = asyncio.create_task(wait_until(
                lambda: device.stats["acknowledged"] >= args.cycles or stop.is_set(), 1e9, 0.02))
            await waiter
            await asyncio.sleep(0.5)  # let the PLC finish its last reads before the line closes
        else:
            await stop.wait()
    finally:
        for task in background:
            task.cancel()
        if opcua is not None:
            await opcua.stop()
        await server.stop()
    s, c = device.stats, server.counters
    print(f"served {s['started']} cycles ({s['done']} done, {s['fault']} fault), "
          f"{s['refused']} commands refused, {server.refused_clients} clients refused", flush=True)
    closed = (("connections refused beyond plc.max_connections", c.over_limit),
              ("idle connections closed", c.idle_closed),
              ("connections closed for bytes that are not Modbus TCP", c.bad_frames),
              ("writes from read-only clients refused", c.read_only_writes),
              ("accept() failures for lack of file descriptors", c.accept_failures))
    notes = [f"{n} {what}" for what, n in closed if n]
    if s["rolls"]:
        notes.insert(0, f"{s['rolls']} rolls of the car asked of the PLC, {s['roll_timeouts']} not confirmed in time")
    if s["steers"]:
        notes.insert(0, f"{s['steers']} steers of the front wheels asked, {s['steer_timeouts']} not reached in time")
    if notes:
        print("; ".join(notes), flush=True)
    return 0


def run(args) -> int:
    config = load_config(args.config)
    plc = config.plc
    device_id = plc.device_id if args.device_id is None else args.device_id
    if not 1 <= device_id <= 247:
        raise ConfigError(f"--device-id {device_id}: a Modbus device id is 1..247")
    transport, where = _transport(args, plc)
    if args.roll_timeout_s is not None and not 0 < args.roll_timeout_s <= 3600:
        raise ConfigError(f"--roll-timeout-s {args.roll_timeout_s:g}: expected more than 0 and at most 3600 s")
    if args.steer_timeout_s is not None and not 0 < args.steer_timeout_s <= 3600:
        raise ConfigError(f"--steer-timeout-s {args.steer_timeout_s:g}: expected more than 0 and at most 3600 s")
    from station.plc.runner import dry_run_runner, measurement_runner, storing_runner
    from station.plc.server import parse_allowed

    parse_allowed(plc.allowed_clients)  # a bad entry fails before anything opens
    if not 0 <= args.delay_s <= 600:
        raise ConfigError(f"--delay-s {args.delay_s:g}: expected 0 to 600 s")
    runner = dry_run_runner(args.fail_every, delay_s=args.delay_s) if args.dry_run \
        else measurement_runner(config, seed=args.seed)
    if args.store and not args.dry_run:
        raise ConfigError("--store goes with --dry-run (a measuring station keeps every cycle anyway)")
    if args.store:
        from station.records.history import open_history
        runner = storing_runner(runner, lambda: open_history(config))
    if args.opcua:
        from station.plc.opcua_server import check_binding
        check_binding(args.opcua_host or config.opcua.host, config.opcua.users)
        if args.opcua_port is not None and not 0 <= args.opcua_port <= 65535:
            raise ConfigError(f"--opcua-port {args.opcua_port}: expected 0..65535")
    logging.basicConfig(level=getattr(logging, args.log_level.upper()), stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # its errors are ours, reported above
    logging.getLogger("asyncua").setLevel(logging.ERROR)  # chatty at info; a bad call is logged as ours
    return asyncio.run(_serve(args, runner, transport, where, device_id, plc, config))

"""`station ui`: the technician's screen, a local web application (docs/ui.md)."""

from __future__ import annotations

import argparse
import sys

from station.commands.arguments import seed


def add_arguments(parser):
    parser.add_argument("--host", help="the address to listen on (default: ui.host of the configuration, 127.0.0.1); "
                                       "any address but loopback needs ui.password_hash")
    parser.add_argument("--port", type=int, help="the port (default: ui.port of the configuration, 8080)")
    parser.add_argument("--seed", type=seed, default=None,
                        help="simulated station only: which random vehicle stands on the lift (default: a new one)")
    parser.add_argument("--hash-password", action="store_true",
                        help="read a password (from the terminal, or one line of standard input) and print the line "
                             "to put in the configuration as ui.password_hash; nothing is served")
    parser.add_argument("--adjust-steps", type=int, default=7, help=argparse.SUPPRESS)  # simulated tie-rod steps


def run(args) -> int:
    if args.hash_password:
        return _hash_password()
    from station.config import load_config
    from station.ui.auth import is_loopback

    config = load_config(args.config)
    host = args.host or config.ui.host
    port = config.ui.port if args.port is None else args.port
    if not 1 <= port <= 65535:
        print(f"--port {port}: expected 1 to 65535", file=sys.stderr)
        return 2
    if not 2 <= args.adjust_steps <= 50:
        print("--adjust-steps: expected 2 to 50", file=sys.stderr)
        return 2
    import uvicorn

    from station.ui.app import build_app
    from station.ui.hardware import Hardware

    hardware = Hardware(config, adjust_steps=args.adjust_steps)
    if args.seed is not None:
        hardware.seed = args.seed
    app = build_app(config, host=host, hardware=hardware, password_hash=config.ui.password_hash)
    shown = f"[{host}]" if ":" in host else host
    print(f"the station's screen: http://{shown}:{port}/"
          + ("" if is_loopback(host) else "  (password required)"), flush=True)
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="warning", access_log=False,
                                           timeout_graceful_shutdown=5))
    try:
        server.run()
    except OSError as e:  # the port is taken, the address is not this PC's
        print(f"cannot listen on {host}:{port}: {e.strerror or e}", file=sys.stderr)
        return 2
    return 0 if server.started else 2


def _hash_password() -> int:
    import getpass

    from station.ui.auth import hash_password

    if sys.stdin.isatty():
        password = getpass.getpass("password: ")
        if getpass.getpass("again: ") != password:
            print("the two passwords differ", file=sys.stderr)
            return 2
    else:
        password = sys.stdin.readline().rstrip("\n")
    if len(password) < 8:
        print("the password must have 8 characters or more", file=sys.stderr)
        return 2
    print(f"ui:\n  password_hash: \"{hash_password(password)}\"")
    return 0

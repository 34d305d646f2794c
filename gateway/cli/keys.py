"""``python -m gateway keys add|rotate|list``: the device keys file (docs/wire-format.md, "Keys").

``add`` makes a random key for a new device, ``rotate`` gives a known device a new one (a
reflashed or replaced board: the gateway then lets it start its boot counter again, with no
collision and no replay, see "A reflashed or replaced board"). Both print the line the board's
config.json needs, on stdout and alone, so a script can take it; what happened goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gateway.cli import CliError


def _device_id(text: str) -> int:
    try:
        dev = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"device id {text!r} is not an integer") from None
    if not 0 <= dev <= 0xFFFFFFFF:
        raise argparse.ArgumentTypeError(f"device id {dev} outside 0..4294967295")
    return dev


def _name(text: str) -> str:
    if "#" in text or not text.isprintable() or not text.strip():
        raise argparse.ArgumentTypeError(f"name {text!r}: printable text without '#'")
    return " ".join(text.split())


def _key_bytes(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"key length {text!r} is not a whole number of bytes "
                                         "(16 to 64; 32 recommended)") from None
    if not 16 <= n <= 64:
        raise argparse.ArgumentTypeError("a key has 16 to 64 bytes (32 recommended)")
    return n


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "keys",
        help="make, rotate and list device keys (the keys file, mode 600)",
        description="Manage the device keys file the ingest service reads (--keys). Keys are "
        "random (secrets module); the file is created 0600, edited atomically, and refused if "
        "other users may read it. A running gateway or ingest service reads the file again by "
        "itself within its maintenance period (10 s by default): no restart.",
        epilog="examples: python -m gateway keys add 7 --keys /etc/serra/keys.txt --name north | "
        "python -m gateway keys rotate 7 --keys /etc/serra/keys.txt (a reflashed board)",
    )
    ks = p.add_subparsers(dest="keys_command", metavar="ACTION", required=True)
    a = ks.add_parser(
        "add", help="a random key for a new device; prints its config.json line",
        description="Add DEVICE_ID with a new random key and print the line for the board's "
        "config.json (it replaces the \"device_id\" and \"key\" lines of "
        "mcu/config.example.json). A device that already has a key is refused: use 'rotate'.")
    r = ks.add_parser(
        "rotate", help="a new key for a known device (reflashed or replaced board)",
        description="Replace the key of DEVICE_ID (kept: its name and the other lines). Use it "
        "when a board is reflashed or replaced: with the new key it may start its boot counter "
        "again at 0; the gateway stores it after everything the old key sent, and the old "
        "key's packets are refused. Prints the new config.json line; a running gateway reads "
        "the file again by itself.")
    for q in (a, r):
        q.add_argument("device_id", type=_device_id, metavar="DEVICE_ID",
                       help="the board's device_id (0..4294967295)")
        q.add_argument("--keys", required=True, type=Path, metavar="FILE",
                       help="the keys file (created if absent)" if q is a else "the keys file")
        q.add_argument("--name", type=_name, help="a label kept in the file, e.g. 'north house'")
        q.add_argument("--bytes", type=_key_bytes, default=32,
                       help="key length in bytes, 16..64 (default 32)")
        q.set_defaults(func=run)
    ls = ks.add_parser("list", help="device ids, key ids and names (never the keys)")
    ls.add_argument("--keys", required=True, type=Path, metavar="FILE", help="the keys file")
    ls.set_defaults(func=run_list)


def config_line(device_id: int, key: bytes) -> str:
    """The firmware's config.json fields for this device, as one line of JSON members."""
    return f'"device_id": {json.dumps(device_id)}, "key": {json.dumps(key.hex())},'


def run(args: argparse.Namespace) -> int:
    from gateway.store.keys import KeyFileError, key_id, new_key, set_key

    rotate = args.keys_command == "rotate"
    try:
        done = set_key(args.keys, args.device_id, new_key(args.bytes), name=args.name,
                       rotate=rotate)
    except KeyFileError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(f"{args.keys}: {exc.strerror or exc}") from None
    print(config_line(done.device_id, done.key))
    what = (f"device {done.device_id}: key {key_id(done.old)} replaced by {key_id(done.key)}"
            if done.old is not None else f"device {done.device_id} added, key id "
            f"{key_id(done.key)}")
    where = f"{args.keys} (created, mode 600)" if done.created_file else str(args.keys)
    print(f"{what} in {where}.\nNext: put the line above in the board's config.json (it "
          "replaces the \"device_id\" and \"key\" lines). A running gateway takes the new key "
          "within its maintenance period (10 s by default), no restart; its log says "
          "'keys file ... read again'.", file=sys.stderr)
    return 0


def run_list(args: argparse.Namespace) -> int:
    from gateway.store.keys import (
        KeyFileError,
        check_permissions,
        is_weak,
        key_id,
        parse_lines,
        read_text,
    )

    try:
        check_permissions(args.keys)
        lines = parse_lines(read_text(args.keys), str(args.keys))
    except KeyFileError as exc:
        raise CliError(str(exc)) from None
    except FileNotFoundError:
        raise CliError(f"{args.keys}: no such keys file; make it with: python -m gateway keys "
                       f"add DEVICE_ID --keys {args.keys}") from None
    except OSError as exc:
        raise CliError(f"{args.keys}: {exc.strerror or exc}") from None
    print(f"{'device':>10}  {'key id':12}  name")
    for k in lines:
        weak = "  (weak key, refused by the gateway: rotate it)" if is_weak(k.key) else ""
        print(f"{k.device_id:>10}  {key_id(k.key):12}  {k.name}{weak}")
    return 0

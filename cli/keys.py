"""``launch.py keys make HOST | list``: the CURVE key pairs of a graph's hosts (docs/hosts.md)."""

from __future__ import annotations

import argparse
import sys


def main(args: argparse.Namespace) -> int:
    from runtime.security import default_key_dir, list_keys, make_key

    key_dir = args.keys or default_key_dir()
    if args.action == "make":
        if not args.host:
            args.parser.error("keys make: name the host")
        try:
            keys = make_key(key_dir, args.host, overwrite=args.overwrite)
        except (FileExistsError, OSError) as err:
            print(f"launch.py keys: {err}", file=sys.stderr)
            return 2
        print(f"{key_dir / args.host}.key: secret key of host {args.host} (mode 0600)")
        print(f'its hosts-table entry: public_key: "{keys.public}"')
        return 0
    rows = list_keys(key_dir)
    for name, public, secret in rows:
        print(f"{name:16} {public}  {'secret key here' if secret else 'public key only'}")
    if not rows:
        print(f"no keys in {key_dir}")
    return 0

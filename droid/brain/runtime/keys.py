"""droid-keys DIR [--name NAME]...: make the CURVE key pairs a cell's links use (thesis §7.1).

Writes one key pair per name in zmq.auth's format: ``DIR/NAME.key`` (the
public key, mode 0644, to copy to every host of the cell) and
``DIR/NAME.key_secret`` (public and secret key, mode 0600, to keep on host
NAME only).  Without ``--name`` it makes a pair for every host of the cell
(``--cell FILE``; under the key names its ``[curve]`` table gives them, if it
has one).  An existing pair is kept unless ``--force``; one line per pair on
stdout: ``NAME PUBLIC_KEY DIR/NAME.key``.  Point the cell file's
``[curve] keys`` at DIR (docs/architecture.md, Messages).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from droid.brain.plumbing.curve import PUBLIC_SUFFIX, SECRET_SUFFIX, load_public_key
from droid.brain.runtime.program import parser
from droid.brain.db.shmdb import check_name_part
from droid.cli import BadInput, RuntimeFailure, run

PROG = "droid-keys"


def make_key_pair(key_dir: Path, name: str, *, force: bool = False) -> tuple[bytes, bool]:
    """Write ``NAME.key`` (0644) and ``NAME.key_secret`` (0600) in ``key_dir``.

    Returns (Z85 public key, True if a new pair was written).  The secret file
    is created under umask 077, so it is never readable by others, not even
    for an instant."""
    import zmq.auth

    public_path = key_dir / f"{name}{PUBLIC_SUFFIX}"
    secret_path = key_dir / f"{name}{SECRET_SUFFIX}"
    if not force and (public_path.exists() or secret_path.exists()):
        if not (public_path.exists() and secret_path.exists()):
            raise BadInput(f"half a key pair for {name!r} in {key_dir}; use --force to replace it")
        return load_public_key(public_path), False
    old = os.umask(0o077)
    try:
        for p in (public_path, secret_path):
            if p.exists():
                p.unlink()
        zmq.auth.create_certificates(key_dir, name)
    finally:
        os.umask(old)
    os.chmod(secret_path, 0o600)
    os.chmod(public_path, 0o644)
    return load_public_key(public_path), True


@run
def main(argv=None) -> int:
    ap = parser(PROG, "Make CURVE key pairs (NAME.key public, NAME.key_secret 0600) for a cell's "
                      "tcp:// links.")
    ap.add_argument("dir", metavar="DIR", help="key directory (created 0700 if missing)")
    ap.add_argument("--name", action="append", metavar="NAME",
                    help="key name (repeatable; default: every host of the cell)")
    ap.add_argument("--force", action="store_true", help="replace existing key pairs")
    args = ap.parse_args(argv)
    if args.name:
        names = args.name
    else:
        from droid.brain.cell.cellfile import load_cell

        cell = load_cell(args.cell)
        hosts = cell.hosts()
        names = [cell.curve.key_name(h) if cell.curve else h for h in hosts]
    for n in names:
        check_name_part(n, "key")
    if len(set(names)) != len(names):
        raise BadInput(f"a key name is given twice: {' '.join(names)}")
    key_dir = Path(args.dir)
    if key_dir.exists() and not key_dir.is_dir():
        raise BadInput(f"{key_dir} exists and is not a directory")
    try:
        key_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as exc:
        raise RuntimeFailure(f"cannot create {key_dir}: {exc.strerror}") from None
    for n in names:
        try:
            public, new = make_key_pair(key_dir, n, force=args.force)
        except PermissionError as exc:
            raise RuntimeFailure(f"cannot write {n!r} in {key_dir}: {exc.strerror}") from None
        if not new:
            print(f"{PROG}: kept the existing key pair {n!r} (--force replaces it)", file=sys.stderr)
        print(f"{n} {public.decode()} {key_dir / (n + PUBLIC_SUFFIX)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

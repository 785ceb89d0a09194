"""`robchair view RUN`: open a run folder in the Rerun viewer (chair, sensors and maps on the run's
timeline), writing its ``recording.rrd`` first when it is missing.

Without a display (no ``DISPLAY`` / ``WAYLAND_DISPLAY`` on Linux) or with ``--no-viewer`` the command
prints the recording's path and how to open it elsewhere. Needs the ``viz`` extra
(``pip install 'robchair[viz]'``: rerun-sdk with its viewer, about 170 MB). It replaces an earlier
``recording.rrd`` of robchair's (one the folder's ``.robchair-output`` lists); any other file of that
name only with ``--overwrite``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "view",
        help="open a run folder in the Rerun viewer (writes RUN/recording.rrd when missing)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("run", help="run folder of robchair sim / robchair run, or a .rrd recording")
    p.add_argument("--rebuild", action="store_true", help="write recording.rrd again even when it exists")
    p.add_argument(
        "--overwrite", action="store_true", help="replace a recording.rrd there that robchair did not write"
    )
    p.add_argument("--no-viewer", action="store_true", help="only write the recording and print its path")
    p.set_defaults(func=_run)


def has_display() -> bool:
    """True where a window can open: always on macOS and Windows, with X11 or Wayland on Linux."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _run(args: argparse.Namespace) -> int:
    from robchair.outdir import add_marker_entry, check_own_file
    from robchair.run_folder import RunFolderError
    from robchair.viz.rerun_recording import RECORDING_NAME, import_rerun, write_recording

    target = Path(args.run)
    if target.is_file() and target.suffix == ".rrd":
        rrd = target
    elif target.is_dir():
        rrd = target / RECORDING_NAME
        if args.rebuild or not rrd.is_file():
            check_own_file(target, RECORDING_NAME, overwrite=args.overwrite)
            import_rerun()  # say how to install before reading anything
            write_recording(target)
            add_marker_entry(target, RECORDING_NAME)
            print(f"wrote {rrd}")
    else:
        raise RunFolderError(f"{target}: not a run folder or a .rrd recording")
    if args.no_viewer or not has_display():
        why = "" if args.no_viewer else " (no display here)"
        print(
            f"recording: {rrd}{why}\nopen it with: rerun {rrd}   (pip install 'robchair[viz]' gives `rerun`)"
        )
        return 0
    import_rerun()
    print(f"opening {rrd} in the Rerun viewer")
    return subprocess.run([sys.executable, "-m", "rerun", str(rrd)], check=False).returncode

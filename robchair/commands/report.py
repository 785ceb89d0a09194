"""`robchair report RUN`: write (again) the self-contained ``report.html`` of a run folder and print its path.

``robchair sim`` writes the report itself; this command builds it for any run folder (e.g. one written
before the report existed, or after ``timeseries.csv`` was added). Page contents: :mod:`robchair.report`.
It replaces an earlier ``report.html`` of robchair's (one the folder's ``.robchair-output`` lists); any
other file of that name only with ``--overwrite``.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "report",
        help="write RUN/report.html: metrics, pictures, 3D structures and plots over time, offline",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("run", help="run folder of robchair sim / robchair run")
    p.add_argument(
        "--overwrite", action="store_true", help="replace a report.html there that robchair did not write"
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from robchair.outdir import add_marker_entry, check_own_file
    from robchair.report import REPORT_NAME, build_report

    if Path(args.run).is_dir():  # build_report names a missing folder
        check_own_file(args.run, REPORT_NAME, overwrite=args.overwrite)
    path = build_report(args.run)
    add_marker_entry(args.run, REPORT_NAME)
    print(path)
    return 0

"""`robchair report RUN`: write (again) the self-contained ``report.html`` of a run folder and print its path.

``robchair sim`` writes the report itself; this command builds it for any run folder (e.g. one written
before the report existed, or after ``timeseries.csv`` was added). Page contents: :mod:`robchair.report`.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = subparsers.add_parser(
        "report",
        help="write RUN/report.html: metrics, pictures, 3D structures and plots over time, offline",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("run", help="run folder of robchair sim / robchair run")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from robchair.report import build_report

    print(build_report(args.run))
    return 0

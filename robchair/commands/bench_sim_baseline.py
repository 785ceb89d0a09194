"""The baseline of `robchair bench sim`: the revision the one drive loop replaced, run as a whole.

The replaced scenario runner (``sim/runner.py``) ran on the simulator of its own time (its Kinect
render, sonar casts and physics). The baseline is that revision entire: the last main-line revision
that had the runner (:func:`baseline_revision`: the first parent of the main-line commit that removed
it) is unpacked with ``git archive`` into a cache folder and run in a child process whose ``sys.path``
starts at that folder, so none of today's modules takes part (:class:`BaselineRunner`). Without git
history (a source archive, no ``git``), there is no baseline.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

OLD_RUNNER = "sim/runner.py"
ROOT = Path(__file__).resolve().parents[2]
_TAG = "@@baseline "  # result lines of the child (PyBullet's C code prints on the same stdout)

# The child: imports only from the unpacked revision, then runs one scenario per JSON request line.
_CHILD = r"""
import json, os, sys
root = sys.argv[1]
sys.path.insert(0, root)
import sim.runner, robchair
for mod in (sim.runner, robchair):
    if not os.path.abspath(mod.__file__).startswith(root + os.sep):
        sys.exit(f"baseline: {mod.__name__} was imported from {mod.__file__}, not from {root}")
def enc(o):
    return o.tolist() if hasattr(o, "tolist") else str(o)
for line in sys.stdin:
    kw = json.loads(line)
    cpus = kw.pop("cpus")
    scenario = kw.pop("scenario")
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[:cpus]))
    try:
        out = {"metrics": sim.runner.run_scenario(scenario, **kw).metrics}
    except Exception as e:
        out = {"error": f"{type(e).__name__}: {e}"}
    print("@@baseline " + json.dumps(out, default=enc), flush=True)
"""


@dataclass(frozen=True)
class Revision:
    """A git revision: full hash, its UTC date and subject."""

    sha: str
    date: str
    subject: str

    def describe(self) -> str:
        """One line naming the revision (short hash, date, subject cut to 70 characters)."""
        subj = self.subject if len(self.subject) <= 70 else self.subject[:67] + "..."
        return f"{self.sha[:10]} ({self.date}, {subj!r})"


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True,
                          check=True).stdout.strip()  # fmt: skip


def baseline_revision() -> Revision | None:
    """The last main-line revision with the replaced runner (None: no git history that has it).

    The main line is the first-parent history of ``HEAD``: the commit on it that removed
    :data:`OLD_RUNNER` (the merge that brought the one loop in) has as its first parent the main line
    as users had it, runner and simulator together.
    """
    try:
        gone = _git("log", "-1", "--first-parent", "--diff-filter=D", "--format=%H", "--", OLD_RUNNER)
        if not gone:
            return None
        sha, date, subject = _git("log", "-1", "--format=%H%x00%ad%x00%s", "--date=format:%Y-%m-%d %H:%M %z",
                                  f"{gone}^1").split("\x00")  # fmt: skip
    except (OSError, subprocess.CalledProcessError, ValueError):
        return None
    return Revision(sha, date, subject)


def _cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "robchair" / "bench-baseline"


def unpack(rev: Revision) -> Path:
    """The revision's tree, unpacked once into the user's cache (``git archive``; reused afterwards, so
    its compiled kernels are cached too); a temporary folder where the cache is not writable."""
    dest = _cache_root() / rev.sha
    if (dest / OLD_RUNNER).is_file():
        return dest
    data = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev.sha], capture_output=True,
                          check=True).stdout  # fmt: skip
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".unpack-", dir=dest.parent))
    except OSError:
        dest = tmp = Path(tempfile.mkdtemp(prefix="robchair-baseline-"))
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(tmp)  # our own history
    if tmp != dest:
        try:
            tmp.rename(dest)
        except OSError:  # another bench unpacked it meanwhile
            return dest if (dest / OLD_RUNNER).is_file() else tmp
    return dest


class BaselineRunner:
    """The replaced revision's ``run_scenario`` in a child process (one process for all runs).

    Args:
        rev: the revision (:func:`baseline_revision`).

    Raises:
        RuntimeError: the child could not start or a run failed (the message says why).
    """

    def __init__(self, rev: Revision) -> None:
        self.rev = rev
        self.root = unpack(rev)
        env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
        # -I: neither today's tree (PYTHONPATH, the script's folder) nor user site-packages on sys.path
        self._proc = subprocess.Popen([sys.executable, "-I", "-c", _CHILD, str(self.root)],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                      env=env)  # fmt: skip

    def run(self, scenario: str, cpus: int, **kw: Any) -> dict[str, Any]:
        """``metrics`` of one ``run_scenario(scenario, **kw)`` of the old revision pinned to ``cpus``."""
        p = self._proc
        assert p.stdin is not None and p.stdout is not None
        try:
            p.stdin.write(json.dumps({"scenario": scenario, "cpus": cpus, **kw}) + "\n")
            p.stdin.flush()
        except (BrokenPipeError, OSError):
            raise RuntimeError(f"baseline process exited ({p.wait()})") from None
        for line in p.stdout:
            if line.startswith(_TAG):
                out = json.loads(line[len(_TAG) :])
                if "error" in out:
                    raise RuntimeError(f"baseline run failed: {out['error']}")
                return dict(out["metrics"])
        raise RuntimeError(f"baseline process exited ({p.wait()})")

    def close(self) -> None:
        """Stop the child process."""
        if self._proc.stdin is not None:
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()

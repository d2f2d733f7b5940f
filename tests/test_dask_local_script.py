"""A script that starts a local Dask cluster without ``if __name__ == "__main__":``: its workers,
started by multiprocessing's spawn, run the script again, and their start fails."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("distributed")

#: A describe on a local cluster at the script's top level: the route is argv 1, the cache argv 2.
UNGUARDED = """
import sys
from wiloc import api
from wiloc.cache.store import Cache
api.describe(sys.argv[1], "sad", cache=Cache(sys.argv[2]), scheduler="local", jobs=1)
"""


def test_a_script_starting_a_local_cluster_without_the_main_guard_is_told_to_add_it(tmp_path: Path) -> None:
    """It ended in Dask's chained tracebacks ("Nanny failed to start."), the reason (multiprocessing's
    bootstrapping error) only in the workers' own; now the error says what the script needs."""
    route = tmp_path / "route"
    route.mkdir()
    cv2.imwrite(str(route / "f0.png"), np.zeros((24, 32), np.uint8))
    script = tmp_path / "unguarded.py"
    script.write_text(UNGUARDED)
    run = subprocess.run([sys.executable, str(script), str(route), str(tmp_path / "cache")], capture_output=True,
                         text=True, timeout=120, check=False)
    assert run.returncode == 1
    assert run.stderr.strip().splitlines()[-1] == (
        "wiloc.errors.WilocError: local: the local Dask cluster's workers failed to start (Nanny failed to start); "
        "a script that starts one must do so under if __name__ == '__main__': (its workers, started by "
        "multiprocessing's spawn, run the script again)"), run.stderr

"""What accuracy costs in time: ``tilerender bench accuracy`` as a benchmark script.

The study itself lives in ``cli/accuracy.py`` (sweep, effect costs, time to quality, the error
estimate's calibration) and ``cli/accuracy_report.py`` (JSON, markdown, plots); see
``docs/accuracy.md`` and ``bench/README.md``. Options are those of the command::

    ./dev bench accuracy --quick                 # a check that it works (a few minutes)
    ./dev bench accuracy --docs                  # the full study, into docs/accuracy.md
"""

import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) in sys.path:  # the packages first: bench/cluster.py is not the cluster package
    sys.path.remove(str(REPO_ROOT))
sys.path.insert(0, str(REPO_ROOT))

from cli.main import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(["bench", "accuracy", *sys.argv[1:]]))

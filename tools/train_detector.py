"""Reproduce the shipped defect model: one command, single-threaded, deterministic.

    .venv/bin/python tools/train_detector.py ../shared/data/defects -o inspect_pipe/saliency_defects/models/defects_v1.npz

Same as ``inspect-pipe detect train DATA -o MODEL``. Trains each class on the
'train' part of its set (split rule in inspect_pipe.saliency_defects._datasets) and never reads
the 'eval' part.
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("OMP_NUM_THREADS", "1")

from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cli.detect import app  # noqa: E402

if __name__ == "__main__":
    sys.exit(app(["train", *sys.argv[1:]], standalone_mode=True))

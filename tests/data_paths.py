"""Where the tests find the shared public data sets: ``../shared/data`` beside the
repository, or the folder named by ``ELASTOCAP_SHARED_DATA``. Tests that need a data set
skip when it is absent."""

import os
from pathlib import Path

SHARED_DATA = Path(os.environ.get("ELASTOCAP_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
TEMPLE = SHARED_DATA / "temple_sparse_ring"
HORSE = SHARED_DATA / "horse_gallop" / "horse_gallop.npz"

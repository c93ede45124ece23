import sys
from pathlib import Path

# The tests also run from a checkout where the package is not installed (liquidgs' own `make
# test` runs them); once it is (`pip install -e .`), this changes nothing.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

"""Test configuration: headless pygame and matplotlib, set before anything imports them;
the repository root on ``sys.path`` so that tests import ``agents`` (not installed)."""

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.append(str(ROOT))  # appended: the installed vslam_gym stays first

os.environ["SDL_VIDEODRIVER"] = "dummy"
os.environ["SDL_AUDIODRIVER"] = "dummy"
os.environ["MPLBACKEND"] = "Agg"
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

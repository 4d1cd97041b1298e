"""Test configuration: headless pygame and matplotlib, set before anything imports them."""

import os

os.environ["SDL_VIDEODRIVER"] = "dummy"
os.environ["SDL_AUDIODRIVER"] = "dummy"
os.environ["MPLBACKEND"] = "Agg"
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

"""Emulators of hardware devices and of their vendors' Python APIs, for tests and rehearsals.

``sdk/`` holds stand-ins for vendor packages with the same module, function names and signatures as the real
ones (read from their public sources, not copied); each talks to an emulator process that models the device's
timing, workspace and force limits. A device adapter puts ``sdk/`` first on ``sys.path`` only when it is told to
emulate (its ``emulator`` parameter), so the real package is used otherwise.
"""

from pathlib import Path

SDK_DIR = str(Path(__file__).parent / "sdk")

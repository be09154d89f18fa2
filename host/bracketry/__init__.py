"""bracketry: an exposure-bracketed stereo camera rig and an offline auto-exposure benchmark.

The ``bracketry`` package (this folder, ``host/bracketry``) holds the command line, the wire protocol and the rig
software that runs on the backpack computer. The offline emulator and benchmark live in ``bracketry_emulator``
(``emulator/bracketry_emulator``) and are installed with the ``emulator`` extra.
"""

__version__ = "0.1.0"

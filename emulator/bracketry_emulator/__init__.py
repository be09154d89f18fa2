"""bracketry_emulator: the offline side of bracketry.

Synthetic HDR worlds, camera-response calibration, exposure emulation from brackets, auto-exposure methods in
closed loop, visual odometry, metrics, statistics and reports. Installed with the ``emulator`` extra.
"""

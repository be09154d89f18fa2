"""Host side of the ESP32 status panel: the panel client (PANEL_STATE out, BUTTON in), the simulator that runs the
real MicroPython firmware files under CPython, and the deploy helper (mpremote)."""

"""The rig daemon: configuration, per-sensor states, buttons, faults, status socket, USB device naming."""

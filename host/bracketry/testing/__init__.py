"""Test harnesses shipped with the package but never used by the rig in the field.

- :mod:`bracketry.testing.faults`: scripted fault scenarios of the whole simulated rig (daemon, fake cameras,
  trigger and panel simulators), each run in its own private network namespace.
- :mod:`bracketry.testing.simrun`: one recording session on fake cameras and a software trigger, run in a private
  network namespace by the recording pipeline tests.

They are importable as modules (``python -m bracketry.testing.faults``), so the tests can run them in a subprocess
inside ``unshare``.
"""

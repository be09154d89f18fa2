"""The STM32 trigger from the host: client (configure, start, stop, events), behavioural simulator, QEMU runner.

- :mod:`bracketry_rig.trigger.client`: :class:`TriggerClient` on :class:`bracketry_rig.wire.link.SerialLink`, producing
  :class:`bracketry_rig.events.TriggerEvent` with host time through the clock model; gap and reboot detection.
- :mod:`bracketry_rig.trigger.simulator`: :class:`TriggerSimulator`, the same protocol over a pty with real-time pulses,
  optional drift, jitter, dropped events and reboots.
- :mod:`bracketry_rig.trigger.qemu`: boot the real firmware ELF in ``qemu-system-arm -M netduinoplus2``.

The firmware lives in ``firmware/stm32_trigger/``; the protocol in ``firmware/protocol/PROTOCOL.md``.
"""

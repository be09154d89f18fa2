"""The scripted session of the simulated rig: SENSORS -> IDLE, RECORD -> REC, N seconds, RECORD -> IDLE, SIGTERM."""

from __future__ import annotations

import signal
import time
from typing import Any

from bracketry.sim.rig import SimulatedRig
from bracketry_base.errors import BracketryError

ALL = ("cam_left", "cam_right", "trigger")


def run_session(rig: SimulatedRig, seconds: float, timeout_s: float = 60.0) -> dict[str, Any]:
    """Drive the started rig through one recording with panel buttons; returns timings and the final state."""
    t0 = time.monotonic()
    rig.wait_screen("TRIG:", timeout_s)  # the daemon drew its first screen: the panel talks to the host
    rig.press("sensors")
    rig.wait_states({k: "IDLE" for k in ALL}, timeout_s)
    rig.wait_screen("L:IDL R:IDL TRIG:IDL", timeout_s)  # the panel shows it too (and the screen is printed)
    rig.press("record")
    rig.wait_states({k: "REC" for k in ALL}, timeout_s)
    rig.wait_screen("L:REC R:REC TRIG:REC", timeout_s)
    t_rec = time.monotonic()
    rig.run_for(seconds)
    rig.press("record")
    state = rig.wait_states({k: "IDLE" for k in ALL}, timeout_s)
    rec_s = time.monotonic() - t_rec
    rig.wait_screen("SAVED", timeout_s)
    rc = rig.stop_daemon(signal.SIGTERM)
    if rc != 0:
        raise BracketryError(f"the daemon exited with code {rc} after SIGTERM (see {rig.out}/daemon.log)")
    return {"recorded_s": round(rec_s, 1), "session_s": round(time.monotonic() - t0, 1), "final_state": state,
            "daemon_exit_code": rc}

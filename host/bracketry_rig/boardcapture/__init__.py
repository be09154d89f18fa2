"""The board capture workflow of ``bracketry calibrate capture`` (docs/CALIBRATION.md, "Capture"): board sessions on
disk (:mod:`.files`), the selection of views and the monitor page (:mod:`.selection`), a session folder read as a
stream (:mod:`.folder`) and the rig of a config driven through its trigger board (:mod:`.trigger_board`); the
simulated rig's capture is :mod:`bracketry.sim.board_capture`."""

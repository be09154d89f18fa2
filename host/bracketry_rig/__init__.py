"""bracketry_rig: the rig software on the backpack computer (ARCHITECTURE.md, "Layers"): cameras, trigger,
pairing, the recorder and session, the daemon, monitor, panel, export and the wire protocol; it imports
the base only."""

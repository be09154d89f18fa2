"""bracketry_base: what the rig and the emulator share, on the core dependencies alone (ARCHITECTURE.md,
"Layers"): errors, progress, paths, output checks, the option types of every command, the PNG writer,
the recording format with its reader and checker, and the stereo calibration library."""

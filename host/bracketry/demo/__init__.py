"""``bracketry demo``: the whole pipeline on the embedded default (simulated rig -> recording -> benchmark)."""

"""Defaults and choices of the closed loop and the benchmark, each defined once (nothing heavy imported: the CLIs
read them while declaring their options).

Exposures in us (in ms on the command line and in output files).
"""

from __future__ import annotations

from bracketry_base.png import PNG_COMPRESSIONS as PNG_COMPRESSIONS

#: the first target exposure (us) of a method that declares none (the authors: 4 ms)
DEFAULT_INIT_EXPOSURE_US = 4000.0
#: the longest exposure any option may ask for (ms): a second is far beyond any bracket of the rig
MAX_EXPOSURE_OPTION_MS = 1000.0
#: lower bound (us) of every target: the authors' only floor (Zhang's 0.02 ms)
DEFAULT_MIN_EXPOSURE_US = 20.0
#: upper bound (us): 2x the sample's longest bracket (beyond it the emulation extrapolates more than one stop)
DEFAULT_MAX_EXPOSURE_US = 64000.0
#: upper bound (dB) of the analog gain a method may set itself (ae/base.py CameraSetting): 24 dB, 16x
DEFAULT_MAX_GAIN_DB = 24.0

#: the emulator's source-bracket selections; the default first
SELECTIONS: tuple[str, ...] = ("highernosat", "upstream", "fusion")
#: the brackets fusion combines (emulation/fusion.py): the pair around the target and every longer one, the pair
#: only, or every bracket; the default first
FUSION_BRACKETS: tuple[str, ...] = ("longer", "bounding", "all")
#: the closed loop's images: emulated from the brackets, or rendered by a synthetic world (truth runs); the default
#: first (the benchmark also takes "both")
#: the longest warm-up a closed loop may take (steps on a trajectory's first view before it; see ae/loop.py)
MAX_WARMUP_STEPS = 100
IMAGES: tuple[str, ...] = ("emulated", "truth")
#: the benchmark's: one of them, or both (then the report compares the two, benchmark/truth_agreement.py)
RUN_IMAGES: tuple[str, ...] = (*IMAGES, "both")
#: the methods as their papers describe them, or as the authors' code runs them; the default first
PARITIES: tuple[str, ...] = ("default", "upstream")
#: camera response: the sample's sRGB-encoded codes (or a pcalib.txt path)
DEFAULT_CRF = "srgb"
#: the camera whose image the AE methods see (the authors: left); the default first
AE_CAMERAS: tuple[str, ...] = ("left", "right")
#: the cameras a closed loop writes; the default last
CAMERAS: tuple[str, ...] = ("left", "right", "both")
#: PNG_COMPRESSIONS: lossless PNG encodings of written images, the default first (imported above: defined with the PNG
#: writer both packages share)

#: localisation backends of the benchmark (benchmark/slam.py); the default first
SLAM_BACKENDS: tuple[str, ...] = ("orbslam3", "builtin")
#: ORB-SLAM3's feed: each frame once its mapping threads are idle (results that do not move with the machine's load)
DEFAULT_SLAM_PACE = "lockstep"
#: the benchmark's reference method of the statistics
DEFAULT_REFERENCE = "ae50"
#: significance level before the Bonferroni correction
DEFAULT_ALPHA = 0.05
#: the methods the statistics cover: the paper's (``all``, or a comma-separated list)
DEFAULT_STATS_METHODS = "paper"

#: batch systems ``bracketry benchmark --cluster`` starts Dask workers on (through dask-jobqueue)
CLUSTERS: tuple[str, ...] = ("slurm",)
#: at most this many Slurm jobs at once (``--jobs``)
DEFAULT_CLUSTER_JOBS = 4
#: the most ``--jobs`` accepts (beyond it, a typo rather than a cluster)
MAX_CLUSTER_JOBS = 10000

"""Statistics of the benchmark: Mann-Whitney U vs a reference method with Bonferroni correction (the paper's), and
paired tests next to it (Wilcoxon signed-rank vs the reference, Friedman across methods, with effect sizes)."""

from bracketry_emulator.stats.mannwhitney import (
    BETTER,
    EQUAL,
    METRICS,
    NA,
    SYMBOL,
    WORSE,
    Comparison,
    compare_to_reference,
    verdict_table,
)
from bracketry_emulator.stats.paired import (
    FriedmanResult,
    PairedComparison,
    friedman,
    rank_biserial,
    wilcoxon_to_reference,
)

__all__ = ["BETTER", "EQUAL", "METRICS", "NA", "SYMBOL", "WORSE", "Comparison", "FriedmanResult", "PairedComparison",
           "compare_to_reference", "friedman", "rank_biserial", "verdict_table", "wilcoxon_to_reference"]

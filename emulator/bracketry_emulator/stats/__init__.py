"""Statistics of the benchmark: Mann-Whitney U vs a reference method with Bonferroni correction."""

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

__all__ = ["BETTER", "EQUAL", "METRICS", "NA", "SYMBOL", "WORSE", "Comparison", "compare_to_reference",
           "verdict_table"]

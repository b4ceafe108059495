"""Evaluation of learned rollouts against LIGGGHTS: metrics per trajectory, figures, reports,
and the paper's variant table (no Lightning, no Hydra: the entry points call these)."""

from granular_pyg.evaluation.compare import variant_table
from granular_pyg.evaluation.figures import comparison_figure
from granular_pyg.evaluation.pair import PairEvaluation, evaluate_pair
from granular_pyg.evaluation.report import write_evaluation

__all__ = [
    "PairEvaluation",
    "comparison_figure",
    "evaluate_pair",
    "variant_table",
    "write_evaluation",
]

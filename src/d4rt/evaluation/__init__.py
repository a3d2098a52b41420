"""Evaluation: metrics, benchmark readers, the synthetic benchmark, baselines and the harness behind
``d4rt eval``. Protocols and their sources are documented in each module (see also docs/evaluation.md)."""

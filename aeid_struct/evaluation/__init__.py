"""Evaluation: paper Table I metrics, scorecards and figures.
"""


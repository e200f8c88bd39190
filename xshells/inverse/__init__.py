"""Target-first design: from a surface to a flat X-shell that deploys onto it (``xshells inverse``).

Data flow: :mod:`.surface` (the checked target) → :mod:`.scissor` (its flat,
closed layout as a metric problem) → :mod:`.net` (beams along the scissor
directions) or :mod:`.flatten` (a designer's own net) → :mod:`.guide` (hold
the deployed state on the target, optimize while letting go) →
:mod:`.metrics` (placement, fit, coverage) → :mod:`.run` (the job and its files).
"""

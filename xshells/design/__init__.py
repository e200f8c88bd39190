"""Design optimization of the rest lengths: low-stress X-shells that fit a target surface (paper §5)."""

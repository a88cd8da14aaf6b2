"""`clods-bench reproduce`: the plan of every table, its digests, and the regression check against committed results."""

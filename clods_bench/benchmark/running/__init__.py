"""Running a task over its seeds, locally or on Ray, and the run records it leaves."""

"""What is made from run records: the paper's tables, the HTML report, plots, image grids and mesh exports."""

"""Gap metrics between simulated and measured runs, with their plots and reports."""

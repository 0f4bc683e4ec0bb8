"""Reports from run folders: plots, renders and the paper's tables (reads files only)."""

"""Data generators: the shipped reference dataset and runs recorded in MuJoCo."""

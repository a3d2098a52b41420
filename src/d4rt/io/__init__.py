"""Reading and writing media and results."""

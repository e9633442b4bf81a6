"""What users run: stylise motions (offline files and, later, live streams)."""

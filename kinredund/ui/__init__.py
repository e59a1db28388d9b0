"""What a user sees: the command line, the demo, plots, progress and meshcat playback."""

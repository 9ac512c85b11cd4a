"""The knowledge sources (agents) of mapinterp, the command line and the pytest plugin."""

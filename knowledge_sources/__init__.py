"""The knowledge sources (agents) of mapinterp, the command line and the pytest plugin."""

from models.blas import default_single_thread

# the agents of a mission share its process: numpy's BLAS starts with one thread per call (before
# numpy is first imported here: the command line, agent hosts; a count the user set is kept)
default_single_thread()

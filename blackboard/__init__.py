"""DOORS-style distributed blackboard over Eclipse Zenoh, with a recorded trace."""

"""robot_agent: the per-robot process of the distributed runtime (one OS process per robot)."""

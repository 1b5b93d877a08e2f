"""swarm: learn decentralized GNN controllers for differential-drive robot swarms and run them
as a real distributed system (one process per robot over Zenoh)."""

__version__ = "0.1.0"

"""PyBullet simulation server: physics of the differential-drive robots."""

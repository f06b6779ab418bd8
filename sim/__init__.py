"""The simulated robot: its servers (Zenoh, CAN), its head-camera node, and the shipped scenes."""

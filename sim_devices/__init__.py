"""sim_devices package."""

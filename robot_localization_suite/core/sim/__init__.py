"""The simulated robot behind ``scan_sim``: scenarios, the simulator and the camera renderer."""

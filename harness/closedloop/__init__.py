"""Closed loop: the device's estimator and controller fly a simulated Crazyflie on UWB alone (issue 9)."""

"""Bundled Python SITL: quadrotor physics, low-level attitude control, target models
and the in-process closed-loop simulator."""

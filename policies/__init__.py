"""Learned candidate samplers (torch, stable-baselines3): see issue 9."""

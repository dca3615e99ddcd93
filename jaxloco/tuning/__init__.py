"""Gradient-based tuning of controller gains through differentiable rollouts."""

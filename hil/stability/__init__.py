"""Stability core: rational network models and exact passivity / absolute-stability criteria."""

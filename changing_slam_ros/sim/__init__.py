"""Scenario simulator for dynamic and changing scenes with full ground truth."""

"""Fault-injecting fake devices for tests."""

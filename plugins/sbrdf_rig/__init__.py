"""Gonioreflectometer rig: serial motor drivers, their simulators, kinematics and pose planning."""

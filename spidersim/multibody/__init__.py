"""Rigid-body algorithms (kinematics, RNEA, CRBA/ABA, base wrench); see the arm issue."""

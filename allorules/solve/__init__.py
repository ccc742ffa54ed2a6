"""Solving: the energy of Eq. 11, the step's transform (Eq. 9), the Gauss-Newton/nlopt solve of one
step, global scaling's 1-D root find, and posture keeping.
"""

"""Hand-held pose: AprilTag detection and pose, SE(3) algebra, synthetic renders, calibration, accuracy.

Imports numpy and cv2 only (never torch).
"""

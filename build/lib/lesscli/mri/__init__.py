"""MRI scans to label volumes (segmentation, phantom frame, reports) and synthetic MRI for tests."""

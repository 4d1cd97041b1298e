"""The vertex-parameter landmark EKF-SLAM estimator (numpy/scipy only).

Never imports gymnasium, pymunk or pygame.
"""

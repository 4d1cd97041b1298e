"""The simulated world: pymunk physics, ray-cast lidar, noisy odometry, world files.

Never imports the estimator (`vslam_gym.slam`).
"""

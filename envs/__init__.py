"""The shipped world files (TOML), importable as package data of ``vslam_gym.worlds``."""

"""mmslam: robust semantic SLAM with max-mixture data association."""

__version__ = "0.1.0"

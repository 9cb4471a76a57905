"""KITTI tracking/odometry: file readers, labels -> Scenario, the LiDAR (PointRCNN) 3D tracker harness."""

"""Dataset readers and adapters (KITTI today). Stages never import this package; pipelines and evaluations do."""

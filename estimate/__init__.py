"""Force estimation from point clouds: PointNet regressor, baselines, training, evaluation."""

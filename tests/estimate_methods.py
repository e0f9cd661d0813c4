"""The methods an evaluation reports, as the tests expect them (written here, not taken from the
code under test)."""

# every model file's evaluation: its baselines and the candidates trained on depth alone
EVALUATED = frozenset(
    {
        "pointnet",
        "mean",
        "linear_displacement",
        "hooke",
        "ridge_height_map",
        "mlp_displacement_history",
        "cnn_depth_change",
        "ensemble_cnn_hooke",
    }
)

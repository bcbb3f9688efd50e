"""What gcnt itself defines, named without importing torch or MuJoCo, so that a run's record can
be checked against it before anything heavy is loaded."""

#: the built-in benchmarks: name -> ``module:attribute``, imported on first use
BENCHMARKS: dict[str, str] = {
    "smpenv": "gcnt.envs.smpenv:SMPENV_BENCHMARK",
    "unimal": "gcnt.envs.unimal:UNIMAL_BENCHMARK",
    "mjcf3d": "gcnt.envs.mjcf3d:MJCF3D_BENCHMARK",
}

#: the built-in methods (:data:`gcnt.nn.registry.BUILTIN_NETWORKS`, which a test holds equal)
METHODS = frozenset(
    {
        "gcnt",
        "gcnt_no_gcn",
        "gcnt_no_wl",
        "gcnt_no_dist",
        "gcnt_dist_first",
        "gcnt_gcn_context",
        "gcnt_hn",
        "amorpheus",
        "swat",
        "smp",
        "metamorph",
        "metamorph_star",
        "modumorph",
        "sr",
        "mlp",
    }
)

"""Many missions as Dask tasks: `semslam study` (simulated worlds over seeds, or a campaign of bags)."""

"""Monte Carlo localization at the level of nav2_amcl (``mcl_baseline``); see docs/mcl.md."""

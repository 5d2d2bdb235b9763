"""The Compare panel: two surfaces registered, their difference map, regions beyond a threshold."""

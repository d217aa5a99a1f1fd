"""Campaigns: stages stored by what they depend on, their settings and presets, the local and Ray backends that run
them, and the run folders that name what they made."""

"""Domains: GridWorld, MiniDungeons, Mario. See :mod:`pcpg_dist.domains.base` for the interface."""

"""rtdenoise.runtime"""

"""rtdenoise.cli"""

"""rtdenoise.export"""

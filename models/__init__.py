"""rtdenoise.models"""

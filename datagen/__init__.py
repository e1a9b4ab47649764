"""rtdenoise.datagen"""

"""deepcrashtest.sim"""

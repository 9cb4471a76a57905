"""deepcrashtest.trajectory"""

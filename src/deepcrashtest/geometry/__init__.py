"""deepcrashtest.geometry"""

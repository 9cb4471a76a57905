"""deepcrashtest.viz"""

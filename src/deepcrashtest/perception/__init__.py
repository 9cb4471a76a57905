"""deepcrashtest.perception"""

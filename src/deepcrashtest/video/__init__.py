"""deepcrashtest.video"""

"""studyctl.participants"""

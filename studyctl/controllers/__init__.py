"""studyctl.controllers"""

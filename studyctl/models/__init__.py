"""studyctl.models"""

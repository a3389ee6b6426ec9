KPL/FK

The Moon's mean-Earth frame chain (from moon_080317.tf and moon_assoc_me.tf), a TK frame
on an IAU frame named through NAIF_BODY_NAME, and a frame class slim does not support.

   \begindata

      FRAME_MOON_ME                 = 31001
      FRAME_31001_NAME              = 'MOON_ME'
      FRAME_31001_CLASS             = 4
      FRAME_31001_CLASS_ID          = 31001
      FRAME_31001_CENTER            = 301
      TKFRAME_31001_SPEC            = 'MATRIX'
      TKFRAME_31001_RELATIVE        = 'MOON_ME_DE421'
      TKFRAME_31001_MATRIX          = ( 1 0 0
                                        0 1 0
                                        0 0 1 )

      FRAME_MOON_PA_DE421           = 31006
      FRAME_31006_NAME              = 'MOON_PA_DE421'
      FRAME_31006_CLASS             = 2
      FRAME_31006_CLASS_ID          = 31006
      FRAME_31006_CENTER            = 301

      FRAME_MOON_ME_DE421           = 31007
      FRAME_31007_NAME              = 'MOON_ME_DE421'
      FRAME_31007_CLASS             = 4
      FRAME_31007_CLASS_ID          = 31007
      FRAME_31007_CENTER            = 301
      TKFRAME_31007_SPEC            = 'ANGLES'
      TKFRAME_31007_RELATIVE        = 'MOON_PA_DE421'
      TKFRAME_31007_ANGLES          = (   67.92     78.56     0.30    )
      TKFRAME_31007_AXES            = (   3,        2,        1       )
      TKFRAME_31007_UNITS           = 'ARCSECONDS'

      FRAME_FUZZY_TILT              = 1400433
      FRAME_1400433_CLASS           = 4
      FRAME_1400433_CENTER          = 2000433
      TKFRAME_FUZZY_TILT_SPEC       = 'ANGLES'
      TKFRAME_FUZZY_TILT_RELATIVE   = 'IAU_FUZZY'
      TKFRAME_FUZZY_TILT_ANGLES     = ( 10 20 30 )
      TKFRAME_FUZZY_TILT_AXES       = ( 1 2 3 )
      TKFRAME_FUZZY_TILT_UNITS      = 'DEGREES'
      NAIF_BODY_NAME               += 'FUZZY'
      NAIF_BODY_CODE               += 2000433

      FRAME_FUZZY_CK                = -1400433
      FRAME_-1400433_CLASS          = 3

      OBJECT_MOON_FRAME =  'MOON_ME'

   \begintext
